"""The independent run `rogs segment` is checked against (tests/segment.rs): the same
input tensor through onnxruntime, its outputs combined as the model's README says
(a lane line where `lanes` argmax is 1, else road where `drivable_area`'s is 1, else
other). Usage: ort_classes.py MODEL INPUT.f32 OUT.u8 (input: float32 [1,3,320,320])."""
import sys

import numpy as np
import onnxruntime as ort

model, inp, out = sys.argv[1:4]
x = np.fromfile(inp, dtype="<f4").reshape(1, 3, 320, 320)
sess = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
names = [o.name for o in sess.get_outputs()]
res = dict(zip(names, sess.run(None, {sess.get_inputs()[0].name: x})))
lanes = res["lanes"][0].argmax(axis=0)
road = res["drivable_area"][0].argmax(axis=0)
cls = np.where(lanes == 1, 2, np.where(road == 1, 1, 0)).astype(np.uint8)
cls.tofile(out)
