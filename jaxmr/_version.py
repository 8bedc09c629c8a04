"""The version of jaxmr (also in pyproject.toml), in a module of its own so that the
modules that write it into files need not import the package.
"""

__version__ = "0.1.0"
