"""rodctl.estimation"""
