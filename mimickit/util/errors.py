"""The one exception type for mistakes a user can make (bad clip, bad config, missing file).

The CLI prints its message as one line on stderr and exits non-zero, never a traceback.
"""


class MimicKitError(Exception):
    """A user-facing error; the message names the file, key or value at fault."""
