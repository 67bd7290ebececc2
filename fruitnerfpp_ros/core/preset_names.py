"""Names of the training presets (``TrainConfig.preset``), importable without torch (the CLI's ``--help``)."""

PRESET_NAMES = ('tiny', 'cpu', 'default', 'paper')
