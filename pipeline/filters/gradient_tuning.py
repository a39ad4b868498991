"""Classical filters tuned by gradient descent: the "optimised Kalman filter" baseline.

The literature on learned Kalman filters warns that a network's win often vanishes once the
classical filter is tuned with the same optimiser, data and loss (issue 17). `TunedFilter` is the
CV, CA, Singer or IMM filter of `torch_filters` whose design values are parameters learned by Adam
on the network-scaled filter's loss (`filter_training`): the process noise, a scale of the plots'
converted-measurement covariance R, a new track's velocity (and acceleration) spread, Singer's
manoeuvre time and the IMM's switch probability. Positive values are learned as logarithms and
the switch probability as log-odds, so every step keeps them valid and moves them relatively.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from pipeline.filters import torch_filters
from pipeline.filters.torch_filters import Filtered, FilterSpec, SequenceBatch

KINDS = ("cv", "ca", "singer", "imm")


class TunedFilter(nn.Module):
    """One filter kind with learnable values, started at `start` and R scale `r_scale`."""

    def __init__(self, start: FilterSpec, r_scale: float = 1.0) -> None:
        super().__init__()
        self.kind = start.kind
        values = {"noise_std": start.noise_std, "velocity_std_mps": start.velocity_std_mps,
                  "r_scale": torch.tensor(r_scale, dtype=start.dtype)}
        if start.kind != "cv":
            values["acceleration_std_mps2"] = start.acceleration_std_mps2
        if start.kind == "singer":
            values["manoeuvre_time_s"] = start.manoeuvre_time_s
        self.logs = nn.ParameterDict({name: nn.Parameter(value.detach().clone().log()) for name, value in values.items()})
        if start.kind == "imm":
            self.switch_logit = nn.Parameter(torch.logit(start.switch_probability.detach().clone()))
            self.register_buffer("initial_cv_probability", start.initial_cv_probability.detach().clone())

    def value(self, name: str) -> Tensor:
        return self.logs[name].exp()

    def spec(self) -> FilterSpec:
        """The filter at the current values (differentiable)."""
        zero = torch.zeros((), dtype=self.logs["noise_std"].dtype)
        imm = self.kind == "imm"
        return FilterSpec(self.kind, self.value("noise_std"), self.value("velocity_std_mps"),
                          self.value("acceleration_std_mps2") if self.kind != "cv" else zero,
                          self.value("manoeuvre_time_s") if self.kind == "singer" else None,
                          torch.sigmoid(self.switch_logit) if imm else None,
                          self.initial_cv_probability if imm else None)

    def forward(self, batch: SequenceBatch, detach_every: int | None = None) -> Filtered:
        return torch_filters.filter_sequences(self.spec(), batch.times, batch.positions,
                                              batch.covariances * self.value("r_scale"), batch.valid, batch.restart,
                                              None, detach_every)

    def to_dict(self) -> dict:
        """The learned values, plain numbers (models/kalman_gradient.json)."""
        values = {name: self.value(name).detach().tolist() for name in self.logs}
        if self.kind == "imm":
            values["switch_probability"] = float(torch.sigmoid(self.switch_logit.detach()))
            values["initial_cv_probability"] = float(self.initial_cv_probability)
        return {"kind": self.kind, **values}

    @classmethod
    def from_dict(cls, values: dict) -> TunedFilter:
        """The filter `to_dict` wrote."""
        spec = FilterSpec(values["kind"], values["noise_std"], values["velocity_std_mps"],
                          values.get("acceleration_std_mps2", 0.0), values.get("manoeuvre_time_s"),
                          values.get("switch_probability"), values.get("initial_cv_probability"))
        return cls(spec, values["r_scale"])
