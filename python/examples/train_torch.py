"""A small PyTorch agent trained on gman's vector environment (A2C, n-step returns), then
evaluated with gman.evaluate on the official episodes.

    pip install ./python torch
    python python/examples/train_torch.py --minutes 3 [--data ../shared/data/gman]

The agent sees the pooled observation embedding and the target's attribute vector (no map,
no LSTM: a feed-forward baseline) and is trained with the paper's mixed reward.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from torch import nn

import gman


class Agent(nn.Module):
    def __init__(self, hidden: int = 256) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Linear(gman.FEATURE_DIM + gman.ATTR_DIM, hidden), nn.ReLU(),
            nn.Linear(hidden, hidden), nn.ReLU(),
        )
        self.pi = nn.Linear(hidden, gman.NUM_ACTIONS)
        self.v = nn.Linear(hidden, 1)

    def forward(self, obs):
        x = torch.cat([torch.from_numpy(obs["features"]), torch.from_numpy(obs["target"])], dim=1)
        h = self.body(x)
        return self.pi(h), self.v(h).squeeze(1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None)
    ap.add_argument("--minutes", type=float, default=3.0)
    ap.add_argument("--num-envs", type=int, default=64)
    ap.add_argument("--n-steps", type=int, default=20)
    ap.add_argument("--lr", type=float, default=7e-4)
    ap.add_argument("--gamma", type=float, default=0.99)
    ap.add_argument("--entropy", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--episodes", type=int, default=None, help="eval: at most N episodes per file")
    a = ap.parse_args()
    torch.manual_seed(a.seed)
    torch.set_num_threads(1)

    env = gman.make_vec_env(data=a.data, split="train", num_envs=a.num_envs, seed=a.seed, copy=True)
    agent = Agent()
    opt = torch.optim.Adam(agent.parameters(), lr=a.lr)
    obs, info = env.reset(seed=a.seed)
    ended = np.zeros(a.num_envs, bool)
    t0, updates, steps = time.time(), 0, 0
    ep_returns, ret = [], np.zeros(a.num_envs)
    while time.time() - t0 < a.minutes * 60:
        logps, values, ents, rewards, masks, valid = [], [], [], [], [], []
        for _ in range(a.n_steps):
            logits, value = agent(obs)
            dist = torch.distributions.Categorical(logits=logits)
            act = dist.sample()
            obs, r, term, trunc, info = env.step(act.numpy())
            # Next-step autoreset: a step taken by an env whose episode had just ended is a
            # reset, not a transition; it is masked out of the loss.
            valid.append(torch.from_numpy(~ended))
            logps.append(dist.log_prob(act))
            values.append(value)
            ents.append(dist.entropy())
            rewards.append(torch.from_numpy(r.astype(np.float32)))
            masks.append(torch.from_numpy(~(term | trunc)).float())
            ret += r * ~ended
            for i in np.flatnonzero(term | trunc):
                ep_returns.append(ret[i])
                ret[i] = 0.0
            ended = term | trunc
            steps += a.num_envs
        with torch.no_grad():
            _, next_v = agent(obs)
        R = next_v * torch.from_numpy(~ended).float()
        loss = torch.zeros(())
        for t in reversed(range(a.n_steps)):
            R = rewards[t] + a.gamma * R * masks[t]
            adv = R - values[t]
            w = valid[t].float()
            loss = loss + (-(logps[t] * adv.detach()) + 0.5 * adv.pow(2) - a.entropy * ents[t]).mul(w).sum()
        loss = loss / (a.n_steps * a.num_envs)
        opt.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(agent.parameters(), 0.5)
        opt.step()
        updates += 1
        if updates % 200 == 0:
            recent = np.mean(ep_returns[-500:]) if ep_returns else float("nan")
            print(f"{time.time() - t0:6.0f} s  {steps:>9} steps  {updates:>6} updates  "
                  f"mean return (last 500 episodes) {recent:.3f}", flush=True)
    print(f"trained {steps} env steps ({updates} updates) in {time.time() - t0:.0f} s")

    @torch.no_grad()
    def policy(obs, info):
        logits, _ = agent(obs)
        return torch.distributions.Categorical(logits=logits).sample().numpy()

    report = gman.evaluate(policy, data=a.data, split="val", episodes=a.episodes, num_envs=64,
                           agent_name="torch-a2c")
    for kind in ("unseen", "seen"):
        k = report["results"][kind]
        print(f"{kind:<7} SR {k['sr']:.2f}  SPL {k['spl']:.2f}  EPA {k['epa']:.2f}  DTS {k['dts']:.2f}  "
              f"({k['episodes']} episodes)")
    rnd = gman.evaluate("random", data=a.data, split="val", episodes=a.episodes)
    print(f"random  SR {rnd['results']['unseen']['sr']:.2f} / {rnd['results']['seen']['sr']:.2f} (unseen / seen)")


if __name__ == "__main__":
    main()
