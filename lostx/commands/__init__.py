"""Sub-commands of the lostx CLI."""
