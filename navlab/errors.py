"""navlab's one user-facing exception type."""


class NavlabError(ValueError):
    """A problem the user can fix; the message says what to change."""
