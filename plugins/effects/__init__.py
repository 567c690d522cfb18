"""plugins/effects"""
