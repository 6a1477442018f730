# ruff: noqa
# Vendored unchanged from MAVSDK (the MAVSDK 4.x Python binding's own example, run as is by
# tests/sitl/test_outsider_mavsdk.py): https://github.com/mavlink/MAVSDK/blob/
# 158e33932461464a9cad473a84349fa0c376d94d/py/mavsdk/examples/takeoff_and_land.py
# Everything after the "end of header" line below is that file byte for byte (its SHA-256 is checked
# by the test). MAVSDK's licence (LICENSE.md at that commit), BSD-3-Clause:
#
# Copyright (c) 2016-2023, MAVSDK Development Team
# All rights reserved.
#
# Redistribution and use in source and binary forms, with or without modification, are permitted
# provided that the following conditions are met:
#
# 1. Redistributions of source code must retain the above copyright notice, this list of conditions
#    and the following disclaimer.
#
# 2. Redistributions in binary form must reproduce the above copyright notice, this list of conditions
#    and the following disclaimer in the documentation and/or other materials provided with the
#    distribution.
#
# 3. Neither the name of the copyright holder nor the names of its contributors may be used to
#    endorse or promote products derived from this software without specific prior written permission.
#
# THIS SOFTWARE IS PROVIDED BY THE COPYRIGHT HOLDERS AND CONTRIBUTORS "AS IS" AND ANY EXPRESS OR
# IMPLIED WARRANTIES, INCLUDING, BUT NOT LIMITED TO, THE IMPLIED WARRANTIES OF MERCHANTABILITY AND
# FITNESS FOR A PARTICULAR PURPOSE ARE DISCLAIMED. IN NO EVENT SHALL THE COPYRIGHT HOLDER OR
# CONTRIBUTORS BE LIABLE FOR ANY DIRECT, INDIRECT, INCIDENTAL, SPECIAL, EXEMPLARY, OR CONSEQUENTIAL
# DAMAGES (INCLUDING, BUT NOT LIMITED TO, PROCUREMENT OF SUBSTITUTE GOODS OR SERVICES; LOSS OF USE,
# DATA, OR PROFITS; OR BUSINESS INTERRUPTION) HOWEVER CAUSED AND ON ANY THEORY OF LIABILITY, WHETHER
# IN CONTRACT, STRICT LIABILITY, OR TORT (INCLUDING NEGLIGENCE OR OTHERWISE) ARISING IN ANY WAY OUT
# OF THE USE OF THIS SOFTWARE, EVEN IF ADVISED OF THE POSSIBILITY OF SUCH DAMAGE.
# ---- end of header ----
import time
from mavsdk import *
from mavsdk.plugins.action import *

def main():
    log_subscribe(lambda level, msg, file, line: True)

    configuration = Configuration.create_with_component_type(ComponentType.GROUND_STATION)

    mavsdk = Mavsdk(configuration)
    mavsdk.add_any_connection("udpin://0.0.0.0:14540")

    drone = None

    def on_new_system(user_data=None):
        nonlocal drone

        print("New system discovered event received")

        for system in mavsdk.get_systems():
            print(f"Checking new system: {system}")

            if system.has_autopilot() and system.is_connected():
                print("✓ Found valid autopilot system!")
                drone = system
                break

    subscription_handle = mavsdk.subscribe_on_new_system(on_new_system)

    print("Waiting for a drone...")
    while drone is None:
        time.sleep(1)

    mavsdk.unsubscribe_on_new_system(subscription_handle)

    if drone:
        action = Action(drone)

        print(f"Using system: {drone}")
        print(f"Takeoff altitude: {action.get_takeoff_altitude()}")
        print(f"RTL altitude: {action.get_return_to_launch_altitude()}")

        print("Arming...")
        action.arm()

        print("Taking off...")
        action.takeoff()

        print("Flying for 2 seconds...")
        time.sleep(2)

        print("Landing...")
        action.land()

        print("Mission complete!")
    else:
        print("No valid system found!")

if __name__ == "__main__":
    main()
