"""Writes a tiny ONNX model with the YOLOv8 output layout whose boxes are known.

Usage: python3 yolo_constant.py OUT.onnx CHANNELS SIZE

Input `images` is 1 x CHANNELS x SIZE x SIZE. Output `output0` is 1 x 6 x 8 (rows cx,
cy, w, h, person score, other-class score; 8 candidates, in input pixels):
candidate 0 is a person at (32, 32) of 16 x 24 whose score is the mean of the input
(a convolution as large as the input averages it, so a model of 3 channels refuses
a 1-channel input); candidate 1 a person scored 0.1; candidate 2 another class.
Everything else is zero. Used by tests/it/gate.rs to run OpenCV dnn end to end.
"""

import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

path, channels, size = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
n = 8
known = np.zeros((1, 6, n), np.float32)
mask = np.zeros((1, 6, n), np.float32)
known[0, 0:4, 0] = [32, 32, 16, 24]
mask[0, 4, 0] = 1.0
known[0, 0:4, 1] = [10, 10, 8, 8]
known[0, 4, 1] = 0.1
known[0, 0:4, 2] = [50, 50, 8, 8]
known[0, 5, 2] = 0.95
# One convolution over the whole input gives all 6 x 8 outputs: its bias is the
# known values, and the kernel of candidate 0's person score averages the input.
weight = np.zeros((6 * n, channels, size, size), np.float32)
weight[mask.reshape(-1) == 1.0] = 1.0 / (channels * size * size)
shape = np.array([1, 6, n], np.int64)
nodes = [
    helper.make_node("Conv", ["images", "weight", "bias"], ["flat"], kernel_shape=[size, size]),
    helper.make_node("Reshape", ["flat", "shape"], ["output0"]),
]
graph = helper.make_graph(
    nodes,
    "yolo-constant",
    [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, channels, size, size])],
    [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 6, n])],
    [
        numpy_helper.from_array(weight, "weight"),
        numpy_helper.from_array(known.reshape(-1), "bias"),
        numpy_helper.from_array(shape, "shape"),
    ],
)
model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 12)])
model.ir_version = 7
onnx.checker.check_model(model)
onnx.save(model, path)
