"""Recordings read: simulated Parquet, a user's Parquet or ASTERIX as one checked plot table, long ones a part
at a time and sorted out of core."""
