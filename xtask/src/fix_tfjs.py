"""Makes a TensorFlow.js graph model made by an older TensorFlow readable by the
one tf2onnx runs with: every attribute the op now has a default for and the node
lacks is set to that default, and `_FusedConv2D`-style nodes get the `TArgs` list
(one type per fused argument) newer TensorFlow requires."""
import json, sys
from google.protobuf import json_format
from tensorflow.python.framework import op_def_registry

src, dst = sys.argv[1], sys.argv[2]
model = json.load(open(src))
nodes = list(model["modelTopology"]["node"])
for f in model["modelTopology"].get("library", {}).get("function", []):
    nodes += f.get("nodeDef", [])
fixed = 0
for n in nodes:
    attr = n.setdefault("attr", {})
    if n["op"] in ("_FusedConv2D", "_FusedMatMul") and "TArgs" not in attr:
        k = int(attr.get("num_args", {}).get("i", "0"))
        attr["TArgs"] = {"list": {"type": [attr["T"]["type"]] * k}}
        fixed += 1
    op = op_def_registry.get(n["op"])
    if op is None:
        continue
    for a in op.attr:
        if a.name not in attr and a.HasField("default_value"):
            attr[a.name] = json_format.MessageToDict(a.default_value)
            fixed += 1
json.dump(model, open(dst, "w"))
print(f"{fixed} attributes added")
