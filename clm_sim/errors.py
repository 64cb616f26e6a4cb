"""The one exception type for user mistakes.

A ``UserError`` is raised for anything a user can fix: a bad config key, a malformed record, an
unstable controller design. Its message is one line that names the file, the key or the column and
what was expected. The CLI prints it and exits with code 2; it never shows a traceback.
"""


class UserError(Exception):
    """A mistake in user input (config, data file, option); the message is shown as is."""
