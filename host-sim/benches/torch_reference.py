#!/usr/bin/env python3
"""PyTorch eager reference of gman-rs's navigator: one step and one inner update (k = 20).

The same networks and sizes as gman-core's `Dims::MCU` / `Dims::PAPER`, batch 1, float32,
one thread (`torch.set_num_threads(1)`), PyTorch being the framework of the original GMAN
implementation:

* G: [z; SE(y)] (45 + 45) -> H -> LeakyReLU(0.2) -> F (512) -> sigmoid
* D: F -> DH -> LeakyReLU(0.2) -> 1
* policy: [s, x, s*x, SE(y), previous probabilities] (3F + 45 + 6) -> E -> LeakyReLU(0.2)
  -> LSTMCell(E, LH) -> actor (6, softmax) and critic (1)
* step: z ~ N(0, I), x = G(z, SE(y)), the policy on (s, x), greedy action, record
  (s, z, probs, h) in the buffer (what `Navigator::step` does; inference mode).
* adaptation (`Navigator::adapt_now` on k = 20 buffered steps): one ascent step of D on the
  WGAN-GP L_D (penalty by autograd with create_graph=True) over the buffer, then one SGD step
  of G and of the actor head on L_ad = -mean_t D(x_t) * ||a_t||, gradients by autograd.
* "adapt2": the same inner step with create_graph=True and a backward pass of L_ad at the
  adapted parameters through it to the pre-adaptation ones (the second-order meta-gradient);
  gman-core has no counterpart (the trainer's `--meta-order 2` uses finite differences).

Prints one JSON object. Run through `host-sim/benches/compare.py`, which runs `gman bench` in
the same invocation and prints the ratios. Never run in CI.

    /path/to/venv/bin/python host-sim/benches/torch_reference.py [--preset mcu --preset paper]
"""

import argparse
import json
import statistics
import sys
import time

try:
    import torch
    import torch.nn.functional as Fn
except ImportError:
    print(
        "PyTorch not installed: pip install torch numpy (in a venv) to run the comparison",
        file=sys.stderr,
    )
    sys.exit(0)

A = 45  # attributes SE(y)
Z = 45  # noise
NA = 6  # actions
K = 20  # buffer size
PRESETS = {
    # gen_hidden, feat, disc_hidden, lstm_hidden, embed (gman-core preset.rs)
    "mcu": dict(H=256, F=512, DH=64, LH=64, E=64),
    "paper": dict(H=4096, F=512, DH=1024, LH=512, E=512),
}


def macs_per_step(p):
    """Same formula as gman-core's Dims::macs_per_step (G, fusion, LSTM, heads)."""
    h, f, lh, e = p["H"], p["F"], p["LH"], p["E"]
    return h * (Z + A) + f * h + e * (3 * f + A + NA) + 4 * lh * (e + lh) + (NA + 1) * lh


class Nav:
    """Parameters as plain tensors so the adaptation can run functionally."""

    def __init__(self, p, seed=1):
        g = torch.Generator().manual_seed(seed)
        h, f, dh, lh, e = p["H"], p["F"], p["DH"], p["LH"], p["E"]

        def w(*shape):
            return (torch.randn(*shape, generator=g) * 0.05).requires_grad_(True)

        self.p = p
        self.gen = [w(h, Z + A), w(h), w(f, h), w(f)]
        self.disc = [w(dh, f), w(dh), w(1, dh), w(1)]
        self.fuse = [w(e, 3 * f + A + NA), w(e)]
        self.lstm = [w(4 * lh, e), w(4 * lh, lh), w(4 * lh), w(4 * lh)]
        self.actor = [w(NA, lh), w(NA)]
        self.critic = [w(1, lh), w(1)]
        self.attr = torch.rand(1, A, generator=g)
        self.rng = torch.Generator().manual_seed(seed + 1)
        self.reset()

    def reset(self):
        lh, f = self.p["LH"], self.p["F"]
        self.h = torch.zeros(1, lh)
        self.c = torch.zeros(1, lh)
        self.prev = torch.full((1, NA), 1.0 / NA)
        self.n = 0
        self.buf_s = torch.zeros(K, f)
        self.buf_z = torch.zeros(K, Z)
        self.buf_p = torch.zeros(K, NA)
        self.buf_h = torch.zeros(K, lh)

    @staticmethod
    def G(gp, z, attr):
        w1, b1, w2, b2 = gp
        u = Fn.leaky_relu(Fn.linear(torch.cat([z, attr.expand(z.shape[0], -1)], 1), w1, b1), 0.2)
        return torch.sigmoid(Fn.linear(u, w2, b2))

    @staticmethod
    def D(dp, x):
        w1, b1, w2, b2 = dp
        return Fn.linear(Fn.leaky_relu(Fn.linear(x, w1, b1), 0.2), w2, b2)

    def step(self, s):
        """One navigation step on the observation s (1 x F); returns the action index."""
        z = torch.randn(1, Z, generator=self.rng)
        x = self.G(self.gen, z, self.attr)
        fused = Fn.leaky_relu(
            Fn.linear(torch.cat([s, x, s * x, self.attr, self.prev], 1), *self.fuse), 0.2
        )
        wx, wh, bx, bh = self.lstm
        self.h, self.c = torch._VF.lstm_cell(fused, (self.h, self.c), wx, wh, bx, bh)
        probs = torch.softmax(Fn.linear(self.h, *self.actor), 1)
        value = Fn.linear(self.h, *self.critic)
        i = self.n % K
        self.buf_s[i] = s[0]
        self.buf_z[i] = z[0]
        self.buf_p[i] = probs[0]
        self.buf_h[i] = self.h[0]
        self.n += 1
        self.prev = probs
        return int(torch.argmax(probs)), value

    def adapt(self, a1=1e-4, a2=1e-4, lam=10.0, second_order=False):
        """One inner update on the K buffered steps."""
        s, zb, hb = self.buf_s, self.buf_z, self.buf_h
        # Lines 15-16: one ascent step of D on L_D (WGAN-GP).
        with torch.no_grad():
            x = self.G(self.gen, zb, self.attr)
        eps = torch.rand(K, 1, generator=self.rng)
        mix = (eps * s + (1 - eps) * x).requires_grad_(True)
        dmix = self.D(self.disc, mix)
        (gmix,) = torch.autograd.grad(dmix.sum(), mix, create_graph=True)
        pen = ((gmix.norm(dim=1) - 1) ** 2).mean()
        ld = self.D(self.disc, s).mean() - self.D(self.disc, x).mean() - lam * pen
        gd = torch.autograd.grad(ld, self.disc)
        with torch.no_grad():
            for p, g in zip(self.disc, gd):
                p.add_(g, alpha=a1)
        # Lines 17-19: SGD of G and the actor head on L_ad.
        theta = self.gen + self.actor

        def l_ad(params):
            gp, ap = params[:4], params[4:]
            xg = self.G(gp, zb, self.attr)
            probs = torch.softmax(Fn.linear(hb, *ap), 1)
            return -(self.D(self.disc, xg)[:, 0] * probs.norm(dim=1)).mean()

        loss = l_ad(theta)
        grads = torch.autograd.grad(loss, theta, create_graph=second_order)
        if second_order:
            adapted = [p - a2 * g for p, g in zip(theta, grads)]
            meta = torch.autograd.grad(l_ad(adapted), theta)
            return float(loss), meta
        with torch.no_grad():
            for p, g in zip(theta, grads):
                p.sub_(g, alpha=a2)
        return float(loss), None


def median_time(fn, reps):
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), min(ts)


def bench_preset(name, reps):
    p = PRESETS[name]
    nav = Nav(p)
    s = torch.rand(1, p["F"], generator=torch.Generator().manual_seed(2))
    out = {"macs_per_step": macs_per_step(p), "sizes": p}

    # Step (inference mode, the best case for eager PyTorch).
    with torch.inference_mode():
        for _ in range(20):
            nav.step(s)
        t0 = time.perf_counter()
        for _ in range(3):
            nav.step(s)
        n = max(1, int(0.01 / ((time.perf_counter() - t0) / 3)))
        per = []
        for _ in range(reps):
            t, _ = median_time(lambda: [nav.step(s) for _ in range(n)], 1)
            per.append(t / n)
    out["step_us"] = statistics.median(per) * 1e6
    out["step_min_us"] = min(per) * 1e6

    # Step with autograd recording (what a training loop pays).
    nav.reset()
    for _ in range(10):
        nav.step(s)
        nav.h, nav.c = nav.h.detach(), nav.c.detach()
    per = []
    for _ in range(reps):
        t0 = time.perf_counter()
        for _ in range(n):
            nav.step(s)
            nav.h, nav.c, nav.prev = nav.h.detach(), nav.c.detach(), nav.prev.detach()
        per.append((time.perf_counter() - t0) / n)
    out["step_autograd_us"] = statistics.median(per) * 1e6

    def fill():
        nav.reset()
        with torch.inference_mode():
            for _ in range(K):
                nav.step(s)
        # inference tensors cannot enter autograd: take plain copies
        nav.buf_s, nav.buf_z = nav.buf_s.clone(), nav.buf_z.clone()
        nav.buf_p, nav.buf_h = nav.buf_p.clone(), nav.buf_h.clone()

    for key, so, r in (("adapt_ms", False, reps), ("adapt2_ms", True, max(3, reps // 2))):
        ts = []
        for i in range(r + 1):
            fill()
            t0 = time.perf_counter()
            nav.adapt(second_order=so)
            if i > 0:
                ts.append(time.perf_counter() - t0)
        out[key] = statistics.median(ts) * 1e3
        out[key.replace("_ms", "_min_ms")] = min(ts) * 1e3
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", action="append", choices=sorted(PRESETS))
    ap.add_argument("--reps", type=int, default=15)
    a = ap.parse_args()
    torch.set_num_threads(1)
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:
        pass
    torch.manual_seed(0)
    res = {
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "k": K,
        "presets": {},
    }
    for name in a.preset or ["mcu", "paper"]:
        print(f"torch_reference: {name} ...", file=sys.stderr)
        res["presets"][name] = bench_preset(name, a.reps)
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
