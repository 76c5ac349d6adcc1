"""The one exception type for mistakes a user can make (bad clip, bad config, missing file).

The CLI prints its message as one line on stderr and exits non-zero, never a traceback.
"""


def shorten(text: str, limit: int) -> str:
    """`text` as an error quotes it: at most `limit` characters, then `...`."""
    return text if len(text) <= limit else text[:limit] + "..."


class MimicKitError(Exception):
    """A user-facing error; the message names the file, key or value at fault."""
