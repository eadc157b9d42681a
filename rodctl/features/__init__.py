"""rodctl.features"""
