"""Plants: linear and nonlinear models, input signals, the scenario catalogue, batched simulation,
model and data files."""
