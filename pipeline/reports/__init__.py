"""What the reports say: the comparison's and the fusion's tables and sentences, the pictures, and the
generated sections of the README and docs/."""
