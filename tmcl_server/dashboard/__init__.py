"""The live dashboard (``tmcl-server --http [HOST:]PORT``): one page in a browser for the whole
server, with a TMCL program debugger.

* :mod:`.core` -- what the page shows and does, without a web server: the state of a module
  as JSON, samples of the axes on simulated time, the decoded wire (from the trace), and the
  page's actions (switches, load, inputs, commands through the router, breakpoints)
* :mod:`.web` -- the aiohttp server: the page, its static files, one WebSocket per browser
* ``static/`` -- the page (HTML, JS, CSS) and the vendored uPlot chart library (MIT)

Imported only when ``--http`` is given (aiohttp is the optional extra ``http``);
docs/dashboard.md describes the page, the update protocol and the debugger.
"""
