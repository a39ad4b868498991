"""Where a plot lies: the thesis's plot-to-ECEF conversion and the exact ones, ASTERIX units and clock, and
elementary functions that give the same bits on every processor."""
