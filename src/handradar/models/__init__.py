"""handradar.models"""
