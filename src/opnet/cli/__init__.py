"""opnet.cli"""
