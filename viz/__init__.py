"""lostx.viz"""
