"""opnet.parameterizations"""
