"""Reproductions of papers' figures and tables: ``nirc-bench reproduce`` (docs/reproduce.md).

A figure is a module here (``<paper>_<figure>.py``, e.g. :mod:`jobs.reproduce.vt_fig7`)
that registers a :class:`~jobs.reproduce.registry.FigureSpec`: what it renders, at the
``quick`` and ``full`` budgets, through the generic parameter sweep (so a point already
stored under its key is read, not rendered again), and how it draws our figure. A run
writes the figure (PNG), and a table of our numbers with their 95 % intervals beside
the paper's (Markdown and JSON, :mod:`jobs.reproduce.results`). The papers' own numbers
and claims live in data files under ``papers/`` (:mod:`jobs.reproduce.papers`).
"""
