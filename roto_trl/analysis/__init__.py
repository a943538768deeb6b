"""Analysis of trained runs: the numbers behind ``roto_trl/analyse.py``."""
