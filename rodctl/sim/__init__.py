"""rodctl.sim"""
