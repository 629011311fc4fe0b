"""handradar.tasks"""
