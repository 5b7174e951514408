"""Bots that join through the coordinator as a crowd of workers would (`crowdteleop bot
--coordinator`): the whole platform under load, measured as the workers live it."""
