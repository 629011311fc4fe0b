"""handradar.hand"""
