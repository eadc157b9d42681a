"""rodctl.control"""
