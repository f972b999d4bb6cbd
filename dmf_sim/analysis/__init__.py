"""Order analysis of recorded bags and the model beside the recording."""
