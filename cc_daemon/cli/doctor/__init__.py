"""`cc-daemon doctor`: is this Pi ready to run the service? Checks with a fix each.

- `system`: the machine as the checks see it, under a root that may be a fake one
  (users and groups, file access as the service user, devices, processes);
- `checks`: each check, returning OK / WARN / FAIL and how to fix it;
- `command`: the command, its output and exit status.
"""
