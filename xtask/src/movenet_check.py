"""Checks a MoveNet MultiPose ONNX conversion: ONNX Runtime loads it, it takes
int32 1xSxSx3 and gives 1x6x56, and a fixed synthetic image gives the output the
first conversion gave (sum of all values; the file's bytes differ run to run)."""
import sys

import numpy as np
import onnxruntime as ort

model, expected = sys.argv[1], float(sys.argv[2])
session = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
(inp,) = session.get_inputs()
x = (np.arange(256 * 256 * 3, dtype=np.int64) * 7919 % 256).astype(np.int32)
out = session.run(None, {inp.name: x.reshape(1, 256, 256, 3)})[0]
assert out.shape == (1, 6, 56), out.shape
total = float(out.sum())
assert abs(total - expected) < 1e-3 * max(1.0, abs(expected)), (total, expected)
print(f"{model}: loads, 1x6x56, synthetic-image sum {total:.4f} as expected")
