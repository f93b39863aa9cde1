"""The methods and modes ``lostx eval`` compares, by name (a module of its own: the command line
lists them without loading the methods)."""

METHODS: dict[str, str] = {
    "lostx": "LoST-X",
    "lostx-nolayout": "LoST-X without the layout",
    "layout": "the layout alone",
    "lost": "LoST",
    "appearance": "appearance (GeM)",
    "thumbnail": "thumbnail (SeqSLAM)",
}
"""Method name -> its label in tables and figures."""
MODES = ("single", "sequence")
"""Single-frame answers, and the same answers through the sequence filter and tracker."""
