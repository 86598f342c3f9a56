"""The one exception type railwatch raises for bad input: its message is the whole story."""


class RailwatchError(Exception):
    """Bad input or a bad state the user can fix; the message says what and how."""


def one_line(e: BaseException) -> str:
    """An exception's message on one line (white space folded), or its type's name."""
    return " ".join(str(e).split()) or type(e).__name__


def naming(source: str, e: BaseException) -> RailwatchError:
    """``e`` as one line that names ``source`` (a file or folder), prefixed unless it does."""
    message = one_line(e)
    return RailwatchError(message if source in message else f"{source}: {message}")
