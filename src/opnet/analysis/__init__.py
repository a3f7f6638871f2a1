"""Analysis tools built on the plugins, kept out of the plugin package: the representation
ceiling of each parameterization (:mod:`opnet.analysis.ceiling`) and the toy scenes it and the
tests use (:mod:`opnet.analysis.toy_scenes`)."""
