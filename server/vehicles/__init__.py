"""Vehicles as separate processes: the graph link, the vehicle host, the supervisor.

See ``server/vehicles/names.py`` for the wire names and DESIGN §3 "Processes".
"""
