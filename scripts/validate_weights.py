import sys, time, json
import numpy as np
import mipnet
from mipnet.training.validation import validation_sets, validate_model, validate_sgbm, format_validation
run = "/root/.cache/mipnet/train/s1-128x256"
trained = mipnet.load(run + "/model.safetensors").eval()
mipnet.manual_seed(0); untrained = mipnet.MIPNet().eval()
sets = validation_sets((256, 320), 8)
sets["motorcycle"] = [mipnet.data.RealPairs("motorcycle")[0]]
out = {}
for name, m in (("trained", trained), ("untrained", untrained)):
    t = time.time(); out[name] = validate_model(lambda l, r: m(l, r, iters=(6, 6)), sets); print(name, time.time() - t, "s")
    print(format_validation(226, out[name]))
out["sgbm"] = validate_sgbm(sets); print(format_validation(0, out["sgbm"]))
json.dump(out, open("/tmp/val226.json", "w"), indent=1)
