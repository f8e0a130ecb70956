"""Engines as Ray actors (``sdfserver serve --cluster``); imported only in cluster mode, so the
embedded server and ``import sdfserver`` never import Ray.

``manager.py`` is the launcher's cluster process: it joins or starts the Ray cluster, creates
the named, detached engine actors (``engine_actor.py``) and reports their addresses and
credentials; API processes then reach each engine straight over its own sockets, as they reach
engine processes on this machine, each connection proving it holds the engine's credential
(``engine/links.py``). Ray places the engines (their GPUs), and restarts one that dies:
the new incarnation restores its worlds from the data directory and listens on the same
address, where the API processes reconnect by themselves.
"""
