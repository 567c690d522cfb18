"""plugins/estimators"""
