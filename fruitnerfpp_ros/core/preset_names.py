"""Names of the training presets (``TrainConfig.preset``), importable without torch (the CLI's ``--help``)."""

PRESET_NAMES = ('tiny', 'cpu', 'default', 'paper')

AUTO = 'auto'
"""The preset a command picks when none is named: :func:`auto_preset` of the device it trains on."""

PRESET_CHOICES = (AUTO, *PRESET_NAMES)

AUTO_ON_CPU_WARNING = ("preset 'auto' on the CPU: using the 'tiny' preset (fast, lower quality); preset 'cpu' counts "
                       "better in about 3x the time; on a CUDA machine 'auto' is 'default'")


def auto_preset(on_cuda: bool) -> str:
    """The preset ``auto`` stands for: ``default`` on a CUDA device, ``tiny`` on the CPU (``AUTO_ON_CPU_WARNING``)."""
    return 'default' if on_cuda else 'tiny'
