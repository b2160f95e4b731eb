"""Latency of one deployment decision (observation build + policy + command) for the shipped
LSA-DSAC model: onnxruntime vs torch eager, one thread, N = 5, 10, 20 humans.

    .venv/bin/python benchmarks/bench_deploy.py [--repeats 2000]

Both run the same :class:`~crowdplan.deploy.runtime.Runtime` step; only the network call
differs. p50 and p99 in milliseconds, and onnxruntime's as a ratio of torch's from the same run.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np
import torch

from crowdplan.deploy.export import export_model
from crowdplan.deploy.onnx_policy import OnnxPolicy
from crowdplan.deploy.runtime import Agent, Runtime
from crowdplan.models import load_model_policy
from crowdplan.policy import PolicyOutput


class TorchPolicy:
    """The torch model behind the OnnxPolicy interface (same features and action mapping)."""

    def __init__(self, onnx_policy: OnnxPolicy, model: str):
        self.onnx = onnx_policy
        self.torch_policy, _ = load_model_policy(model)
        self.manifest, self.max_humans = onnx_policy.manifest, onnx_policy.max_humans
        self.kinematics = onnx_policy.kinematics

    def act(self, robot, humans, mask) -> PolicyOutput:
        return self.torch_policy.act(robot, humans, mask)

    def velocities(self, actions, robot, trip_heading=None):
        return self.onnx.velocities(actions, robot, trip_heading)


def decision_latencies(policy, humans: int, repeats: int) -> np.ndarray:
    """Seconds per Runtime.step for one robot among ``humans`` humans."""
    rng = np.random.default_rng(humans)
    agents = [Agent("r", "robot", goal=(0.0, 4.0))]
    agents += [Agent(f"h{k}", "human") for k in range(humans)]
    runtime = Runtime(policy, agents)
    positions = rng.uniform(-4, 4, (humans, 2))
    times = np.empty(repeats)
    for i in range(repeats + 50):
        t = i * 0.25
        runtime.pose("r", t, 0.0, -4.0 + 1e-3 * i, 0.0)
        for k in range(humans):
            runtime.pose(f"h{k}", t, *(positions[k] + 1e-3 * i), 0.0)
        start = time.perf_counter()
        runtime.step(t)
        if i >= 50:  # warm-up
            times[i - 50] = time.perf_counter() - start
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2000)
    parser.add_argument("--model", default="lsa-dsac")
    args = parser.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        export_model(args.model, tmp)
        onnx_policy = OnnxPolicy(tmp, threads=1)
    torch_policy = TorchPolicy(onnx_policy, args.model)
    print(f"one decision of {args.model}, 1 thread, {args.repeats} repeats (ms)")
    print(
        f"{'N':>3} {'torch p50':>10} {'torch p99':>10} {'ort p50':>9} {'ort p99':>9} ratio p50/p99"
    )
    for n in (5, 10, 20):
        t_torch = decision_latencies(torch_policy, n, args.repeats) * 1e3
        t_ort = decision_latencies(onnx_policy, n, args.repeats) * 1e3
        p_torch, p_ort = np.percentile(t_torch, [50, 99]), np.percentile(t_ort, [50, 99])
        print(
            f"{n:>3} {p_torch[0]:>10.3f} {p_torch[1]:>10.3f} {p_ort[0]:>9.3f} {p_ort[1]:>9.3f} "
            f"{p_ort[0] / p_torch[0]:.2f} / {p_ort[1] / p_torch[1]:.2f}"
        )


if __name__ == "__main__":
    main()
