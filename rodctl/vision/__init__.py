"""rodctl.vision"""
