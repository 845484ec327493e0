"""The transition studio: a local web server (:mod:`.server`) and its three.js page (``static/``).

Start it with ``posturemap serve [INPUT...] [--map MAP]``. The browser side is plain ES modules;
three.js is vendored into ``static/vendor/`` by ``make web`` (pinned in ``package.json``), so the
page works offline.
"""
