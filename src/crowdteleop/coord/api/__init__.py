"""The HTTP API and the pages: each router parses, calls one service and shapes the answer."""
