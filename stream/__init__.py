"""lostx.stream"""
