"""``python -m vmp`` runs the ``vmp`` command."""

from vmp.cli import main

raise SystemExit(main())
