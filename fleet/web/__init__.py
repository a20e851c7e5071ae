"""The fleet controller's HTTP API: transport orders added, withdrawn and read at run time.

``server.WebServer`` is an IoDriver that serves the API (``api``, ``models``) with uvicorn
in its own thread; every request passes the guard (``guard``: host, token, body size) and
is answered by the scan at its quiet point through the ``desk.OrderDesk``.
``plc-runtime run CONFIG --web HOST:PORT`` starts it (``options``), ``plc-runtime order``
talks to it. It is version 1 of the API the operator's web interface builds on.

Nothing is imported here: the command line loads FastAPI and uvicorn only when ``--web``
is given.
"""
