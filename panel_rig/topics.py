"""Topic-name conventions shared by the node (live topics) and the recording (bags), with no dependencies."""

#: a command the rig refused is echoed live and recorded on ``<command topic>/rejected``
REJECTED_SUFFIX = "/rejected"
