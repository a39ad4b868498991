"""Where the learned estimators' batched steps run: `tracker.device` (cpu, cuda or cuda:N; issue 29).

On a GPU the network-scaled filter's and the LSTM update's state tensors, the plots of a call and
the network live on the device; the estimators hand numpy arrays back at the role boundary
(`pipeline.tracker.kalman_net_estimator`, `lstm_update_estimator`). The params package checks the
value's form (`pipeline.params.tracking`); whether the device exists is known only to torch, so it
is checked here, when an estimator is built: a ParamError (exit 2) naming the key and value.
"""

from __future__ import annotations

import copy
import weakref

import torch
from torch import nn

from pipeline.params import ParamError
from pipeline.params.tracking import DEVICE

_PLACED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # model -> {device: its copy there}


def resolve(device: str) -> torch.device:
    """The torch device of `tracker.device` = `device`; ParamError naming the key and value when it is not
    cpu, cuda or cuda:N, or when torch sees no such CUDA device on this machine."""
    if not isinstance(device, str) or not DEVICE.fullmatch(device):
        raise ParamError(f"tracker.device = {device!r}: must be cpu, cuda or cuda:N")
    chosen = torch.device(device)
    if chosen.type == "cuda":
        if not torch.cuda.is_available():
            raise ParamError(f"tracker.device = {device!r}: torch {torch.__version__} sees no CUDA device on this "
                             "machine (torch.cuda.is_available() is False); use cpu")
        if chosen.index is not None and chosen.index >= torch.cuda.device_count():
            raise ParamError(f"tracker.device = {device!r}: this machine has {torch.cuda.device_count()} CUDA "
                             f"device(s), cuda:0 to cuda:{torch.cuda.device_count() - 1}")
    return chosen


def placed(model: nn.Module, device: torch.device) -> nn.Module:
    """`model` itself on the CPU; elsewhere a copy of it moved to `device` (the loaded model is left where
    it is, for other users), made once per model and device."""
    if device.type == "cpu":
        return model
    copies = _PLACED.setdefault(model, {})
    if str(device) not in copies:
        copies[str(device)] = copy.deepcopy(model).to(device).eval()
    return copies[str(device)]
