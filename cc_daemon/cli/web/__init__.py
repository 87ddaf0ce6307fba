"""`cc-daemon web`: the field page, a separate read-only process (docs/web.md).

It reads the daemon's status socket (with a timeout) and the journal (read-only,
through `JournalReader`), and serves them as a page and as JSON. It must never
write to either, never import the daemon, and never answer anything but GET: a
bug here can cost the page, never a cast.
"""
