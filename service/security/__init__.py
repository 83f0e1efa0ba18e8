"""Security: API tokens, scopes and which addresses the service may listen on."""
