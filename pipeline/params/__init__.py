"""Load `params.yaml` into typed, validated objects: each knob declared once, on its section.

Every stage reads its knobs through here so that a bad value stops the stage before it
writes anything, with a message naming the key and the value (``radar.latitude_deg =
95.0: must be in [-90.0, 90.0]``) instead of a traceback deep inside the simulation. The
sections are dataclasses whose fields declare their knobs (`declare.knob`: type, bounds, doc),
read by one parser (`declare.parse_section`); docs/params.md is written from the declarations
(`python -m pipeline params-reference`). The package is the ground floor: it imports nothing of
the pipeline (`pipeline.settings` adds the registries' name checks).
"""

from pipeline.params.declare import ParamError, ParamsLoader, load_params_tree
from pipeline.params.learning import (TUNING_COSTS, Association, Confirmation, Kalman, KalmanNet, LSTMUpdate, NetworkTraining,
                                      Training)
from pipeline.params.tracking import (MIA, Associate, Candidates, Evaluate, EvaluationRun, Fusion, FusionRadar,
                                      LSTMUpdateGate, Management, Networks, Params, Peers, RealTraffic, Scorecard, Site,
                                      StoneSoupPeer, TrackerParams, parse_tree)
from pipeline.params.world import (STRATEGIES, Aircraft, ClimbDive, ConstantJerk, RandomTurns, Radar, Routes, Scenes,
                                   Split, SustainedTurns, Windows, formation_resolution_m)

__all__ = ["MIA", "STRATEGIES", "TUNING_COSTS", "Aircraft", "Associate", "Association", "Candidates", "ClimbDive",
           "Confirmation", "ConstantJerk", "Evaluate", "EvaluationRun", "Fusion", "FusionRadar", "Kalman", "KalmanNet", "LSTMUpdate",
           "LSTMUpdateGate", "Management", "NetworkTraining", "Networks", "ParamError", "Params", "ParamsLoader",
           "Peers", "Radar", "RandomTurns", "RealTraffic", "Routes", "Scenes", "Scorecard",
           "Site", "Split", "StoneSoupPeer", "SustainedTurns", "TrackerParams", "Training", "Windows", "formation_resolution_m",
           "load_params_tree", "parse_tree"]
