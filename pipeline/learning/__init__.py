"""The trained pieces: training windows and their scaling, the thesis's networks and the learned filters, their
training with Lightning, the model files, fast inference and MLflow."""
