"""opnet.data"""
