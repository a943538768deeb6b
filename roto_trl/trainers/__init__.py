"""What turns a config into a training run: builders (config -> objects), the PPO and auxiliary
updates, checkpoints, episode evaluation and metric logging. Imported by the programs at the top
of the package; it imports envs, transforms, modules, objectives and data, never a program."""
