"""The one way the project compiles a kernel (see :mod:`milestones.jit`: the leaf package holds
it so that ``milestones`` and ``vmp`` compile alike without the leaf importing ``vmp``)."""

from milestones.jit import kernel

__all__ = ["kernel"]
