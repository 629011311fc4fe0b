"""handradar.world"""
