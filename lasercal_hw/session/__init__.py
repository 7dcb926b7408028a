"""The session.mcap recording: its format, the writer and the reader (no run logic)."""
