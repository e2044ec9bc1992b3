"""The motives that move a car to another lane or change its speed for one, each tied to its switch
in `Rules`, one module each: strategic (out of a lane that stops leading on), cooperative (letting
in a car whose lane ends or that asks, zip fashion), speed gain (passing a slower leader) and keep
right; wishes.py gathers them into each car's lane wish."""
