"""The one exception type railwatch raises for bad input: its message is the whole story."""


class RailwatchError(Exception):
    """Bad input or a bad state the user can fix; the message says what and how."""
