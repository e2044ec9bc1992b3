"""The road: lane geometry from the net, routes and lane ends, who is near whom."""
