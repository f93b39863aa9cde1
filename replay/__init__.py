"""lostx.replay"""
