"""The operator console served by `fw deploy` (see server.py)."""
