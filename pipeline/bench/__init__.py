"""Scoring trackers: the thesis's metrics, OSPA and GOSPA, evaluations over the test scenarios, the scenes and
other radar sites spread over processes, and the two-radar fusion and association benches."""
