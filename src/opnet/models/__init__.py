"""opnet.models"""
