"""plugins/kinematics"""
