"""Hydra sweeper plugin ``hydra/sweeper=optuna``: an Optuna study over Hydra's sweep syntax.

Our own, on current Optuna: the official ``hydra-optuna-sweeper`` pins ``optuna<3``, which breaks
on RDB storage with SQLAlchemy 2. Hydra finds this package through the ``hydra_plugins``
namespace package (no ``hydra_plugins/__init__.py``). ``config.py`` registers the config,
``sweeper.py`` is the plugin class and ``_study.py`` the study loop, imported only when a sweep
runs so that ordinary runs do not pay for importing Optuna.
"""
