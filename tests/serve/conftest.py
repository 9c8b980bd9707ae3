"""Serve tests use the tiny random-weight checkpoint and its pipeline of tests/conftest.py (``checkpoint``,
``pipe``); their helpers are in serve_helpers.py."""
