"""Sources of scan frames: the scenario simulator, log readers and writers, serial scanners.

Every source yields :class:`vmp.types.ScanFrame` and implements :class:`vmp.source.Source`;
nothing here knows about mapping. :func:`open_source` opens any of them by name.
"""

from drivers.open import open_source

__all__ = ["open_source"]
