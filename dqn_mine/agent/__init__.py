"""The agent: the dueling Q-network (`network`) and the learning maths (`learning`)."""
