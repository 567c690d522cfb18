"""plugins/sensors"""
