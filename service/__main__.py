"""``python -m service`` runs the nirc-bench CLI."""

from service.entry import main

main()
