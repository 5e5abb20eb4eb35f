"""The web app's routes by area, each an ``APIRouter`` that
:func:`quatmotion.server.app.create_app` includes.

* :mod:`~quatmotion.server.routers.pages`: the pages (``/``, ``/play``, ``/compare``,
  ``/search``, ``/poses``) and the static files they load.
* :mod:`~quatmotion.server.routers.clips`: ``/api/info`` and ``/api/clips...`` (the clips,
  their frames, their comparison with the originals).
* :mod:`~quatmotion.server.routers.build`: ``/api/build``, where a library being built is.
* :mod:`~quatmotion.server.routers.search`: ``/api/search`` and ``/api/search/upload``.
* :mod:`~quatmotion.server.routers.poses`: ``/api/poses``.
"""
