"""Sources of scan frames: the scenario simulator, log readers and writers, serial scanners.

Every source yields :class:`vmp.types.ScanFrame`; nothing here knows about mapping.
"""
