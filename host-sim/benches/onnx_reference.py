#!/usr/bin/env python3
"""ONNX Runtime reference of gman-rs's navigator step: f32 and dynamically quantised int8.

The step network of `torch_reference.py` (the sizes of gman-core's `Dims::MCU` /
`Dims::PAPER`, batch 1), written directly as an ONNX graph with `onnx.helper` (no PyTorch
needed) and run by ONNX Runtime with one thread (intra- and inter-op), sequential execution,
all graph optimisations:

* G: [z; SE(y)] -> H -> LeakyReLU(0.2) -> F -> sigmoid = x
* fusion: [s, x, s*x, SE(y), previous probabilities] -> E -> LeakyReLU(0.2)
* LSTM cell (E -> LH; the four gates as two MatMuls, Split, sigmoid / tanh)
* actor (6, softmax) and critic (1)

"int8" is `onnxruntime.quantization.quantize_dynamic` with int8 weights: every MatMul becomes
an integer matrix product with activations quantised on the fly (what a user who picks ONNX
Runtime for an int8 model gets). The noise z is an input here (gman-core draws it inside the
step: 45 normal samples, well under 1 % of the mcu step). Before timing, the f32 session's
outputs are checked against a NumPy evaluation of the same weights.

Prints one JSON object. Run through `host-sim/benches/compare.py`; never run in CI.

    VENV/bin/pip install onnx onnxruntime numpy
    VENV/bin/python host-sim/benches/onnx_reference.py [--preset mcu --preset paper]
"""

import argparse
import json
import os
import statistics
import sys
import tempfile
import time

try:
    import numpy as np
    import onnx
    import onnxruntime as ort
    from onnx import TensorProto, helper, numpy_helper
    from onnxruntime.quantization import QuantType, quantize_dynamic
except ImportError:
    print(
        "ONNX Runtime not installed: pip install onnx onnxruntime numpy (in a venv) to run it",
        file=sys.stderr,
    )
    sys.exit(0)

A, Z, NA = 45, 45, 6
PRESETS = {
    "mcu": dict(H=256, F=512, LH=64, E=64),
    "paper": dict(H=4096, F=512, LH=512, E=512),
}


def weights(p, seed=1):
    """Random weights laid out for `x @ W` (input-major), scale 0.05 as the torch reference."""
    rng = np.random.default_rng(seed)
    h, f, lh, e = p["H"], p["F"], p["LH"], p["E"]

    def w(*shape):
        return (rng.standard_normal(shape) * 0.05).astype(np.float32)

    return {
        "g_w1": w(Z + A, h), "g_b1": w(h), "g_w2": w(h, f), "g_b2": w(f),
        "f_w": w(3 * f + A + NA, e), "f_b": w(e),
        "l_wx": w(e, 4 * lh), "l_wh": w(lh, 4 * lh), "l_b": w(4 * lh),
        "a_w": w(lh, NA), "a_b": w(NA), "c_w": w(lh, 1), "c_b": w(1),
    }


def build(p, W):
    """The step as an ONNX model (opset 17)."""
    f, lh = p["F"], p["LH"]
    n = helper.make_node
    nodes = [
        n("Concat", ["z", "attr"], ["gin"], axis=1),
        n("MatMul", ["gin", "g_w1"], ["g1m"]), n("Add", ["g1m", "g_b1"], ["g1"]),
        n("LeakyRelu", ["g1"], ["g1r"], alpha=0.2),
        n("MatMul", ["g1r", "g_w2"], ["g2m"]), n("Add", ["g2m", "g_b2"], ["g2"]),
        n("Sigmoid", ["g2"], ["x"]),
        n("Mul", ["s", "x"], ["sx"]),
        n("Concat", ["s", "x", "sx", "attr", "prev"], ["fin"], axis=1),
        n("MatMul", ["fin", "f_w"], ["fm"]), n("Add", ["fm", "f_b"], ["fa"]),
        n("LeakyRelu", ["fa"], ["fused"], alpha=0.2),
        n("MatMul", ["fused", "l_wx"], ["gx"]), n("MatMul", ["h", "l_wh"], ["gh"]),
        n("Add", ["gx", "gh"], ["gxh"]), n("Add", ["gxh", "l_b"], ["gates"]),
        n("Split", ["gates"], ["gi", "gf", "gg", "go"], axis=1),
        n("Sigmoid", ["gi"], ["i"]), n("Sigmoid", ["gf"], ["fg"]),
        n("Tanh", ["gg"], ["g"]), n("Sigmoid", ["go"], ["o"]),
        n("Mul", ["fg", "c"], ["fc"]), n("Mul", ["i", "g"], ["ig"]),
        n("Add", ["fc", "ig"], ["c_out"]),
        n("Tanh", ["c_out"], ["tc"]), n("Mul", ["o", "tc"], ["h_out"]),
        n("MatMul", ["h_out", "a_w"], ["am"]), n("Add", ["am", "a_b"], ["logits"]),
        n("Softmax", ["logits"], ["probs"], axis=1),
        n("MatMul", ["h_out", "c_w"], ["cm"]), n("Add", ["cm", "c_b"], ["value"]),
    ]
    vi = lambda name, d: helper.make_tensor_value_info(name, TensorProto.FLOAT, [1, d])  # noqa: E731
    inputs = [vi("s", f), vi("z", Z), vi("attr", A), vi("prev", NA), vi("h", lh), vi("c", lh)]
    outputs = [vi("probs", NA), vi("value", 1), vi("h_out", lh), vi("c_out", lh)]
    init = [numpy_helper.from_array(v, k) for k, v in W.items()]
    graph = helper.make_graph(nodes, "gman_step", inputs, outputs, init)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def numpy_step(W, x):
    """The same step in NumPy, to check the f32 session."""
    lrelu = lambda v: np.where(v > 0, v, 0.2 * v)  # noqa: E731
    sig = lambda v: 1 / (1 + np.exp(-v))  # noqa: E731
    g = sig(lrelu(np.concatenate([x["z"], x["attr"]], 1) @ W["g_w1"] + W["g_b1"]) @ W["g_w2"]
            + W["g_b2"])
    fin = np.concatenate([x["s"], g, x["s"] * g, x["attr"], x["prev"]], 1)
    fused = lrelu(fin @ W["f_w"] + W["f_b"])
    gi, gf, gg, go = np.split(fused @ W["l_wx"] + x["h"] @ W["l_wh"] + W["l_b"], 4, axis=1)
    c = sig(gf) * x["c"] + sig(gi) * np.tanh(gg)
    h = sig(go) * np.tanh(c)
    logits = h @ W["a_w"] + W["a_b"]
    e = np.exp(logits - logits.max())
    return e / e.sum(), h @ W["c_w"] + W["c_b"], h, c


def session(path):
    o = ort.SessionOptions()
    o.intra_op_num_threads = 1
    o.inter_op_num_threads = 1
    o.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    o.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(path, o, providers=["CPUExecutionProvider"])


def time_step(sess, feed, reps):
    for _ in range(50):
        sess.run(None, feed)
    t0 = time.perf_counter()
    for _ in range(20):
        sess.run(None, feed)
    n = max(1, int(0.02 / ((time.perf_counter() - t0) / 20)))
    per = []
    for _ in range(reps):
        t0 = time.perf_counter()
        for _ in range(n):
            sess.run(None, feed)
        per.append((time.perf_counter() - t0) / n)
    return statistics.median(per) * 1e6, min(per) * 1e6


def bench_preset(name, reps, tmp):
    p = PRESETS[name]
    W = weights(p)
    rng = np.random.default_rng(2)
    feed = {
        "s": rng.random((1, p["F"]), dtype=np.float32),
        "z": rng.standard_normal((1, Z)).astype(np.float32),
        "attr": rng.random((1, A), dtype=np.float32),
        "prev": np.full((1, NA), 1 / NA, dtype=np.float32),
        "h": np.zeros((1, p["LH"]), dtype=np.float32),
        "c": np.zeros((1, p["LH"]), dtype=np.float32),
    }
    f32 = os.path.join(tmp, f"{name}-f32.onnx")
    q8 = os.path.join(tmp, f"{name}-int8.onnx")
    onnx.save(build(p, W), f32)
    quantize_dynamic(f32, q8, weight_type=QuantType.QInt8)
    out = {"sizes": p}
    s32, s8 = session(f32), session(q8)
    want = numpy_step(W, feed)
    for got, ref, what in zip(s32.run(None, feed), want, ("probs", "value", "h", "c")):
        if not np.allclose(got, ref, rtol=1e-4, atol=1e-5):
            sys.exit(f"onnx_reference: {name} f32 {what} differs from NumPy by "
                     f"{np.abs(got - ref).max():.3g}")
    probs8 = s8.run(None, feed)[0]
    out["int8_probs_max_abs_err"] = float(np.abs(probs8 - want[0]).max())
    for key, sess in (("f32", s32), ("int8", s8)):
        med, mn = time_step(sess, feed, reps)
        out[f"{key}_step_us"], out[f"{key}_step_min_us"] = med, mn
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", action="append", choices=sorted(PRESETS))
    ap.add_argument("--reps", type=int, default=15)
    a = ap.parse_args()
    res = {"onnxruntime": ort.__version__, "threads": 1, "presets": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.preset or ["mcu", "paper"]:
            print(f"onnx_reference: {name} ...", file=sys.stderr)
            res["presets"][name] = bench_preset(name, a.reps, tmp)
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
