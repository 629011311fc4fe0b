"""handradar.viz"""
