"""handradar.sim"""
