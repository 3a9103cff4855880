"""The README's whole chain as a library: train -> evaluate -> quantise -> export -> run every backend -> verify.

Run it from any folder (it writes deploy/ and report/ there): ``python docs/examples/quickstart.py``.
"""

import vprsnn_export as vx

vx.set_threads(1)
cfg = vx.Config().replace(**{"encoder.timesteps": 60, "train.epochs": 4, "network.n_neurons": 64})
data = vx.load_dataset("synthetic:24", ["summer", "winter"], cfg.preprocess)
ckpt = vx.train_and_calibrate(data, ["summer"], cfg, progress=False)
readout = vx.SequenceOptions(ks=(1, 3))  # gamma is the config's (cfg.assignment.gamma)
winter, places, reference = data.traversal("winter"), data.place_ids, {"summer": data.traversal("summer")}
print(vx.evaluate_float(ckpt, winter, places, "winter", readout).rows)

model = vx.deploy(ckpt, "quickstart", 4, reference_images=reference)
exported = vx.export_and_check(vx.ExportSource.of(model, "quickstart"), model, ("nir", "onnx", "loihi"), "deploy")
spikes = vx.query_spikes(winter, places, "winter", cfg)
backends = [vx.IntegerNetwork(model), vx.ReferenceStepper(model), vx.OnnxBackend(exported.written("onnx"))]
counts = {backend.name: backend.run(spikes[:3]).counts for backend in backends}
print({name: int(c.sum()) for name, c in counts.items()})

options = vx.VerifyOptions(readout, bits=(8,))
query = data.query("winter", ["summer"])  # frames, place ids and the truth that judges them, built once
run = vx.verify_checkpoint(vx.VerifiedNetwork(ckpt, "quickstart", reference), query, options)
vx.write_report(vx.build_report([run], {"example": "quickstart"}), "report")
print("verdict:", "PASS" if run.passed else "FAIL")
