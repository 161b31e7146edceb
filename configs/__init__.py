"""The shipped configuration files, installed as the package ``quadslam_env.configs``.

``scenarios/*.yaml`` (the env's scenarios), ``agents/*.yaml`` (stable-baselines3
hyperparameters per env id) and ``sweeps/*.yaml`` (the example sweep specs). The folder sits at
the top of the repository (docs/design.md §1); ``pyproject.toml`` maps it to
``quadslam_env.configs`` (``package-dir``) and ships the YAML files as its package data, so an
installed wheel and an editable install both read them through :mod:`importlib.resources`.
:func:`quadslam_env.config.files.config_dir` is the one place that locates them.
"""
