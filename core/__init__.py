"""lostx.core"""
