"""handradar.data"""
