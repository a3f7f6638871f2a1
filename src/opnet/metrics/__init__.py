"""opnet.metrics"""
