"""What protects the coordinator and its workers: rate and HTTP limits, security headers,
client addresses, join identities, TLS, tokens, private files, and how refusals leave."""
