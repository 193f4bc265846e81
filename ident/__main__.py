"""``python -m ident ...`` is the ``hdrive`` command (for environments whose scripts folder is not on PATH)."""
from .cli import main

raise SystemExit(main())
