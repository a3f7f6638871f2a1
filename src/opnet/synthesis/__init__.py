"""opnet.synthesis"""
