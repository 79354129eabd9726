"""The stress study: generated hard scenes rendered by every method, and which of them
fail how. Imports the core (``jobs.protocol``), the views (``jobs.views``) and the
record; no other study."""
