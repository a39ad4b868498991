"""Where the data is simulated: aircraft routes, the rotating radar over them, the multi-target scenes, and
the numbers that say whether the data is what was asked for."""
