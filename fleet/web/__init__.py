"""The fleet controller's operator page and HTTP API: plant, vehicles, transport orders,
blockades, tags (watch, write, force), statistics, events and a live stream.

``server.WebServer`` is an IoDriver that serves the API (``api``, ``models``) and the page
(``page/``) with uvicorn in its own thread; every request passes the guard (``guard``: host,
rate, token, body size) and is answered by the scan between two scans through the desks
(``desk`` for orders, ``fleet_desk`` for the rest), which copy what is asked (``views``);
``feed`` streams snapshots. ``plc-runtime run CONFIG --web HOST:PORT`` starts it
(``options``), ``plc-runtime order`` talks to it, ``apidoc`` renders docs/api.md.

Nothing is imported here: the command line loads FastAPI and uvicorn only when the web
server is asked for.
"""
