"""The yardsticks of air-traffic surveillance: CAT062 system tracks out and in, and the scorecard."""
