"""``python -m vmp``: the ``vmp`` command."""

from vmp.cli import main

raise SystemExit(main())
