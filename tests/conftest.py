"""Shared test setup: one torch thread (several times faster for these small networks)."""

import torch

torch.set_num_threads(1)
