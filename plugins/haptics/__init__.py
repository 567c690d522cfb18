"""plugins/haptics"""
