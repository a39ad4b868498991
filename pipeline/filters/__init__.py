"""The classical filters: filterpy's CV, CA and IMM as the reference, the one batched Kalman core (NumPy and
PyTorch), their motion models, and their tuning by Nelder-Mead and by gradient descent."""
