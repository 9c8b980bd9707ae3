"""Adapters: small low-rank updates of a model that teach it a user's moves (``smf adapt``), merged at load."""
