"""handradar.gap"""
