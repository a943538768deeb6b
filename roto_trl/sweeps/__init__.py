"""Hyperparameter sweeps: where an Optuna study lives and how a sweep is reported."""
