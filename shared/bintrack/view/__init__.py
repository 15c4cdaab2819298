"""``bintrack view``: a live map of a network in the browser, or of a recording with a time slider.

* :mod:`.map_messages`: bus messages → the compact JSON items a page draws;
* :mod:`.map_state`: the picture a page needs (latest tracks, tails, lit sensors…), bounded;
* :mod:`.map_server`: the aiohttp app, one WebSocket per page, drop-to-latest per page;
* :mod:`.recording_source`: a recording played into a page, seekable (MCAP index);
* ``static/``: the page, with Leaflet vendored from npm (``static/leaflet/``, its LICENSE).
"""
