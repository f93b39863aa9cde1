"""lostx: streaming LoST-X place recognition."""
__version__ = "0.1.0"
