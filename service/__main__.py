"""``python -m service`` runs the nirc-bench CLI."""

from service.cli import main

main()
