"""Radar tracking with neural networks: simulation, training, tracking and evaluation.

Importing the package pins the numerical kernels PyTorch picks by processor (issue 27), so that a training
or an evaluation gives the same bytes on any x86-64 processor with AVX2 (every one since 2015), not only on
one like the machine that made the committed run. PyTorch chooses its kernels per processor, and each
choice sums in its own order: a model trained on an AVX-512 machine differed in every file from one
trained on AVX2 (tiny params, all six trainings; docs/data.md, "The same bytes on any processor"). The
three choices, each read by its library at its first computation, not at import:

- `ATEN_CPU_CAPABILITY=avx2`: PyTorch's own vectorised kernels (elementwise, reductions) at AVX2 width
  on an AVX-512 processor too (PyTorch's documented override of its CPU dispatch);
- `MKL_CBWR=AVX2,STRICT`: MKL's conditional numerical reproducibility (Intel oneMKL developer guide,
  "Obtaining Numerically Reproducible Results"): the AVX2 code path on every processor that has it, and
  in strict mode the same bits whatever the number of threads;
- `ONEDNN_MAX_CPU_ISA=AVX2`: oneDNN (PyTorch's float32 LSTM and GRU kernels) at most AVX2 (oneDNN's
  documented CPU dispatcher control).

A variable the user has set is kept (`os.environ.setdefault`): `ATEN_CPU_CAPABILITY=avx512` brings back
the fastest kernels of an AVX-512 machine, at the price of its own bytes. Other architectures (ARM) are
left alone: their kernels are their own. ONNX Runtime (the thesis networks' inference) has no such
control; its kernels may still differ by processor.
"""

import os
import platform

__version__ = "0.1.0"

PORTABLE_KERNELS = {"ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "AVX2,STRICT", "ONEDNN_MAX_CPU_ISA": "AVX2"}

if platform.machine().lower() in ("x86_64", "amd64"):
    for _name, _value in PORTABLE_KERNELS.items():
        os.environ.setdefault(_name, _value)
