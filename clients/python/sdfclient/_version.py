"""The client's version: the distribution's (pyproject.toml reads it here) and its User-Agent's."""

__version__ = "0.1.0"
USER_AGENT = f"sdfclient/{__version__}"  # on every request and on the stream's handshake
