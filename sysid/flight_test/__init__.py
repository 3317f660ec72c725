"""flight_test"""
