"""The record: the database models, the store, the database connection and its
migrations, content-addressed artifacts, settings and retention. Imports nothing
else of ``jobs``."""
