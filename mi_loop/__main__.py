"""``python -m mi_loop`` runs the ``mi-loop`` command line."""
import sys

from mi_loop.app.cli import main

sys.exit(main())
